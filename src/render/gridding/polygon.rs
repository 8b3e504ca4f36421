//! Exact-footprint gridding: each pixel gets `value` times the fraction of the projected
//! quadrangle's area inside it, computed from the quadrangle's edges (see [`splat_linear`]).
//!
//! With a [`Slope`], the value is spread with a *linear* density over the footprint
//! (second-order conservative remapping): the density is `value/area + g . (x - centroid)`, so
//! each pixel gets `value * area_f/area + g . (M_f - centroid area_f)` with `M_f` the first
//! moment of its fragment. The fragments' first moments sum to `centroid * area`, so the
//! gradient term moves energy between pixels but never creates or loses any.
//!
//! Returns `false` (and grids nothing) when the footprint is not a usable polygon: a corner
//! could not be projected, the quadrangle folds over itself (at the limb), it is degenerate,
//! or it spans more than `MAX_SPAN_PX` pixels. The caller then falls back to a point kernel.

use super::{Accum, floor_i64, to_fixed};

const MAX_SPAN_PX: i64 = 64;
/// Footprints whose bounding box covers at most this many pixels are cut by peeling (see
/// [`splat_peel`]), larger ones by edge sums.
const PEEL_MAX_CELLS: usize = 9;
/// A convex quadrangle cut by two pairs of parallel lines keeps at most 8 vertices.
const MAX_VERTS: usize = 8;

type Poly = ([[f64; 2]; MAX_VERTS], usize);

#[inline(always)]
fn verts(p: &Poly) -> &[[f64; 2]] {
    &p.0[..p.1]
}
#[inline(always)]
fn cross(o: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
}

/// Shoelace signed area and first moments `(int x dA, int y dA)` of a polygon (all three carry
/// the orientation's sign: counter-clockwise positive in a y-up frame). Inlined, so callers
/// that use only the area pay only for the area.
#[inline(always)]
fn area_moments(v: &[[f64; 2]]) -> (f64, f64, f64) {
    let n = v.len();
    let (mut a, mut mx, mut my) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let j = if i + 1 == n { 0 } else { i + 1 };
        let c = v[i][0] * v[j][1] - v[j][0] * v[i][1];
        a += c;
        mx += (v[i][0] + v[j][0]) * c;
        my += (v[i][1] + v[j][1]) * c;
    }
    (0.5 * a, mx / 6.0, my / 6.0)
}

/// Centroid `[u, v]` and unsigned area [px^2] of a quadrangle footprint (`None` if degenerate).
#[inline]
pub fn centroid_area(c: &[[f64; 2]; 4]) -> Option<([f64; 2], f64)> {
    let (a, mx, my) = area_moments(c);
    (a.is_finite() && a.abs() > 1e-300).then(|| ([mx / a, my / a], a.abs()))
}

/// A linear density over a footprint: gradient `grad` [value/px^3] about `centroid` [px].
#[derive(Clone, Copy, Debug, Default)]
pub struct Slope {
    pub centroid: [f64; 2],
    pub grad: [f64; 2],
}

/// The value a fragment of a footprint receives from its signed area `a` and first moments
/// `(mx, my)` (same orientation as the footprint's signed area `total`; coordinates in the
/// frame of `centroid`): `value a / total`, plus the gradient's first-moment part.
#[derive(Clone, Copy)]
struct Density {
    k: f64,
    sign: f64,
    slope: Option<Slope>,
}

impl Density {
    #[inline(always)]
    fn new(value: f64, total: f64, slope: Option<&Slope>, origin: [f64; 2]) -> Density {
        Density {
            k: value / total,
            sign: total.signum(),
            slope: slope.map(|s| Slope {
                centroid: [s.centroid[0] - origin[0], s.centroid[1] - origin[1]],
                grad: s.grad,
            }),
        }
    }

    /// Uniform densities use only `a`; `moments` is called for linear ones.
    #[inline(always)]
    fn fragment(&self, a: f64, moments: impl FnOnce() -> (f64, f64)) -> f64 {
        match &self.slope {
            None => a * self.k,
            Some(s) => {
                let (mx, my) = moments();
                let g = s.grad[0] * (mx - s.centroid[0] * a) + s.grad[1] * (my - s.centroid[1] * a);
                a * self.k + g * self.sign
            }
        }
    }
}

/// Grids `value` over the footprint `c` with the linear density of `slope` (uniform if `None`).
///
/// The footprint's area and first moments in each pixel come from its edges alone (Green's
/// theorem, as font rasterisers compute coverage): each edge is cut at the pixel lines, each
/// piece adds the moments of the region between it and its pixel's right side, and the band
/// of its rows further right is added by a prefix sum along the row. The cost grows with the
/// footprint's perimeter in pixels, not with its area or number of pixel fragments.
#[inline]
pub fn splat_linear(c: &[[f64; 2]; 4], value: f64, slope: Option<&Slope>, acc: &mut Accum) -> bool {
    if c.iter().any(|p| !(p[0].is_finite() && p[1].is_finite())) {
        return false;
    }
    // Convex and consistently oriented: all corner turns have the same sign.
    let t = [
        cross(c[3], c[0], c[1]),
        cross(c[0], c[1], c[2]),
        cross(c[1], c[2], c[3]),
        cross(c[2], c[3], c[0]),
    ];
    let pos = t.iter().all(|&x| x >= 0.0);
    let neg = t.iter().all(|&x| x <= 0.0);
    if !(pos || neg) {
        return false;
    }
    let (mut umin, mut umax, mut vmin, mut vmax) = (c[0][0], c[0][0], c[0][1], c[0][1]);
    for p in &c[1..] {
        umin = umin.min(p[0]);
        umax = umax.max(p[0]);
        vmin = vmin.min(p[1]);
        vmax = vmax.max(p[1]);
    }
    let (i0, i1, j0, j1) = (
        floor_i64(umin),
        floor_i64(umax),
        floor_i64(vmin),
        floor_i64(vmax),
    );
    if i0 == i1 && j0 == j1 {
        acc.add(i0, j0, value);
        return true;
    }
    if i1 - i0 >= MAX_SPAN_PX || j1 - j0 >= MAX_SPAN_PX {
        return false;
    }
    let total = area_moments(c).0;
    if total.abs() < 1e-300 || !total.is_finite() {
        return false;
    }
    let (nx, ny) = ((i1 - i0 + 1) as usize, (j1 - j0 + 1) as usize);
    if nx * ny <= PEEL_MAX_CELLS {
        splat_peel(
            c,
            (i0, i1, j0, j1),
            Density::new(value, total, slope, [0.0; 2]),
            acc,
        );
        return true;
    }
    // Local coordinates: pixel (i0, j0) is [0, 1) x [0, 1), which keeps the moments well
    // conditioned far from the image origin.
    let (ox, oy) = (i0 as f64, j0 as f64);
    let local = c.map(|p| [p[0] - ox, p[1] - oy]);
    let density = Linear::new(value, total, slope, [ox, oy]);
    let cells = nx * ny;
    // Taken out of `acc` for the loop below (which adds to `acc`), put back at the end. It is
    // all zero between footprints: the row pass below zeroes every sum it reads.
    let mut m = std::mem::take(&mut acc.scratch.cells);
    if m.len() < 3 * cells {
        m.resize(3 * cells, 0.0);
    }
    let (inner, band) = m[..3 * cells].split_at_mut(cells);
    for e in 0..4 {
        edge_sums(local[e], local[(e + 1) % 4], nx, ny, &density, inner, band);
    }
    // The edge sums are the density's integral over the region right of the boundary: minus
    // the footprint's. Along each row, the bands of the edges to the left are summed in.
    let (band_value, band_height) = band.split_at_mut(cells);
    let (x0, scale) = (acc.x0, acc.scale);
    for j in 0..ny {
        let this_row = j * nx..(j + 1) * nx;
        let Some(row) = acc.row(j0 + j as i64) else {
            // Another band's row.
            inner[this_row.clone()].fill(0.0);
            band_value[this_row.clone()].fill(0.0);
            band_height[this_row].fill(0.0);
            continue;
        };
        let (mut b, mut h) = (0.0, 0.0);
        for i in 0..nx {
            let cell = j * nx + i;
            b += std::mem::take(&mut band_value[cell]);
            h += std::mem::take(&mut band_height[cell]);
            let frag = -(std::mem::take(&mut inner[cell]) + b + density.gx * i as f64 * h);
            let x = (i0 + i as i64 - x0) as usize; // wraps to huge left of the window
            if frag > 0.0 && x < row.len() {
                row[x] += to_fixed(frag, scale);
            }
        }
    }
    acc.scratch.cells = m;
    true
}

/// The linear density of [`Density`] in the form the edge sums use (local coordinates, the
/// footprint's orientation folded in): a region of signed area `a` and first moments
/// `(mx, my)` holds `k0 a + gx mx + gy my`.
struct Linear {
    k0: f64,
    gx: f64,
    gy: f64,
}

impl Linear {
    #[inline(always)]
    fn new(value: f64, total: f64, slope: Option<&Slope>, origin: [f64; 2]) -> Linear {
        let k = value / total;
        match slope {
            None => Linear {
                k0: k,
                gx: 0.0,
                gy: 0.0,
            },
            Some(s) => {
                let sign = total.signum();
                let (gx, gy) = (sign * s.grad[0], sign * s.grad[1]);
                let (cx, cy) = (s.centroid[0] - origin[0], s.centroid[1] - origin[1]);
                Linear {
                    k0: k - gx * cx - gy * cy,
                    gx,
                    gy,
                }
            }
        }
    }
}

/// Splits `p` along `coord[axis] = at` into the parts below (`lo`) and above (`hi`), in
/// one pass, writing both in place (a polygon is 136 bytes: returned by value and copied
/// on, they made `memmove` 19 % of the analytic frame at 1 quadrangle per pixel).
#[inline(always)]
fn split(p: &Poly, axis: usize, at: f64, lo: &mut Poly, hi: &mut Poly) {
    lo.1 = 0;
    hi.1 = 0;
    let (v, n) = (&p.0, p.1);
    if n == 0 {
        return;
    }
    let push = |q: &mut Poly, x: [f64; 2]| {
        if q.1 < MAX_VERTS {
            q.0[q.1] = x;
            q.1 += 1;
        }
    };
    let mut prev = v[n - 1];
    let mut prev_lo = prev[axis] <= at;
    for &cur in v.iter().take(n) {
        let cur_lo = cur[axis] <= at;
        if cur_lo != prev_lo {
            let t = (at - prev[axis]) / (cur[axis] - prev[axis]);
            let mut x = [
                prev[0] + t * (cur[0] - prev[0]),
                prev[1] + t * (cur[1] - prev[1]),
            ];
            x[axis] = at;
            push(lo, x);
            push(hi, x);
        }
        if cur_lo {
            push(lo, cur);
        } else {
            push(hi, cur);
        }
        prev = cur;
        prev_lo = cur_lo;
    }
}

/// Small footprints (a few pixels): the footprint is cut along the pixel grid, one pixel
/// column peeled off at a time, then one pixel row from each column, and each piece's moments
/// taken directly. Faster than the edge sums when there are only a few pieces.
///
/// What is left to cut lives in one of two buffers and each cut writes into the other
/// ([`Peeler`]), so no polygon is copied but each column once.
#[inline(always)]
fn splat_peel(
    c: &[[f64; 2]; 4],
    (i0, i1, j0, j1): (i64, i64, i64, i64),
    density: Density,
    acc: &mut Accum,
) {
    let frag = |p: &Poly| -> f64 {
        let (a, mx, my) = area_moments(verts(p));
        density.fragment(a, || (mx, my)).max(0.0)
    };
    // Peel off one pixel column at a time, then one pixel row at a time from each column.
    // The buffers are taken out of `acc` for the loop (which adds to `acc`), put back at the
    // end.
    let mut peelers = acc.scratch.peel.take().unwrap_or_default();
    let Peelers { columns, rows } = &mut *peelers;
    columns.restart_quad(c);
    for i in i0..=i1 {
        let col = columns.peel(0, i + 1, i == i1);
        if col.1 < 3 {
            continue;
        }
        rows.restart(col);
        for j in j0..=j1 {
            let cell = rows.peel(1, j + 1, j == j1);
            if cell.1 >= 3 {
                acc.add(i, j, frag(cell));
            }
        }
    }
    acc.scratch.peel = Some(peelers);
}

/// The peeling's buffers, one [`Peeler`] for the columns and one for the rows of each
/// column: a band's, reused footprint after footprint (set up anew for each footprint, their
/// 816 bytes were 1.7 % of the instructions of the 1-per-pixel frame).
pub(super) struct Peelers {
    columns: Peeler,
    rows: Peeler,
}

impl Default for Peelers {
    fn default() -> Peelers {
        Peelers {
            columns: Peeler::empty(),
            rows: Peeler::empty(),
        }
    }
}

const EMPTY: Poly = ([[0.0; 2]; MAX_VERTS], 0);

/// A polygon cut into cells one edge at a time: what lies beyond the last cut is in
/// `rest[at]`, and each cut writes its part below the edge into `part` and what lies beyond
/// into the other buffer.
struct Peeler {
    rest: [Poly; 2],
    at: usize,
    part: Poly,
}

impl Peeler {
    #[inline(always)]
    fn empty() -> Peeler {
        Peeler {
            rest: [EMPTY; 2],
            at: 0,
            part: EMPTY,
        }
    }

    /// Starts cutting `p`.
    #[inline(always)]
    fn restart(&mut self, p: &Poly) {
        self.rest[0] = *p;
        self.at = 0;
    }

    /// Starts cutting the quadrangle `c`.
    #[inline(always)]
    fn restart_quad(&mut self, c: &[[f64; 2]; 4]) {
        self.rest[0].0[..4].copy_from_slice(c);
        self.rest[0].1 = 4;
        self.at = 0;
    }

    /// The part of what is left below the cell edge `edge` along `axis` (all of it for the
    /// last cell); what lies beyond is kept for the next cut.
    #[inline(always)]
    fn peel(&mut self, axis: usize, edge: i64, last: bool) -> &Poly {
        if last {
            return &self.rest[self.at];
        }
        let [a, b] = &mut self.rest;
        let (from, beyond) = if self.at == 0 { (&*a, b) } else { (&*b, a) };
        split(from, axis, edge as f64, &mut self.part, beyond);
        self.at = 1 - self.at;
        &self.part
    }
}

/// Adds one directed edge `p -> q` (local pixel coordinates, inside `nx x ny` pixels) to the
/// edge sums: for each piece of the edge inside one pixel, the density's integral over the
/// region between the piece and the pixel's right side (`inner`), and for the pixels further
/// right along the row, the integral over the piece's band but for the part linear in the
/// pixel's column (`band`: the band's value at column 0, then its height; deltas summed along
/// the row by the caller).
#[inline(always)]
fn edge_sums(
    p: [f64; 2],
    q: [f64; 2],
    nx: usize,
    ny: usize,
    density: &Linear,
    inner: &mut [f64],
    band: &mut [f64],
) {
    let d = [q[0] - p[0], q[1] - p[1]];
    if d[1] == 0.0 {
        return; // a horizontal edge bounds no band
    }
    let cells = nx * ny;
    // Walked pixel by pixel (a DDA): along each axis the pixel the edge starts in, the
    // parameter of its next pixel-line crossing, their spacing, and the step in pixels.
    let walk = |x: f64, dx: f64| -> (i64, f64, f64, i64) {
        if dx > 0.0 {
            let c = floor_i64(x);
            (c, (c as f64 + 1.0 - x) / dx, 1.0 / dx, 1)
        } else if dx < 0.0 {
            let c = -floor_i64(-x) - 1;
            (c, (c as f64 - x) / dx, -1.0 / dx, -1)
        } else {
            (floor_i64(x), f64::INFINITY, f64::INFINITY, 0)
        }
    };
    let (mut ci, mut tx, dtx, si) = walk(p[0], d[0]);
    let (mut cj, mut ty, dty, sj) = walk(p[1], d[1]);
    let (last_i, last_j) = (nx as i64 - 1, ny as i64 - 1);
    let Linear { k0, gx, gy } = *density;
    let mut a = p;
    let mut t0 = 0.0;
    while t0 < 1.0 {
        let t1 = tx.min(ty).min(1.0);
        let (cross_x, cross_y) = (tx <= t1, ty <= t1);
        if cross_x {
            tx += dtx;
        }
        if cross_y {
            ty += dty;
        }
        let b = if t1 >= 1.0 {
            q
        } else {
            [p[0] + t1 * d[0], p[1] + t1 * d[1]]
        };
        let dy = b[1] - a[1];
        if dy != 0.0 {
            // The footprint lies in the `nx x ny` pixels: the walk leaves them only by a
            // rounding at a pixel line, on a piece of no length.
            let i = ci.clamp(0, last_i) as usize;
            let j = cj.clamp(0, last_j) as usize;
            let x_right = (i + 1) as f64;
            let cell = j * nx + i;
            let sy = a[1] + b[1];
            // The region's area and first moments (Green's theorem along the piece).
            let area = dy * (x_right - 0.5 * (a[0] + b[0]));
            let mx = dy
                * 0.5
                * (x_right * x_right - (a[0] * a[0] + a[0] * b[0] + b[0] * b[0]) * (1.0 / 3.0));
            let my = dy
                * (0.5 * x_right * sy
                    - (a[0] * (2.0 * a[1] + b[1]) + b[0] * (a[1] + 2.0 * b[1])) * (1.0 / 6.0));
            inner[cell] += k0 * area + gx * mx + gy * my;
            if i + 1 < nx {
                // The band over one pixel at column `i'` holds `dy (k0 + gx (i' + 1/2)) +
                // gy dy sy / 2`: all but `gx i' dy` goes here.
                band[cell + 1] += dy * (k0 + 0.5 * gx) + 0.5 * gy * dy * sy;
                band[cells + cell + 1] += dy;
            }
        }
        if cross_x {
            ci += si;
        }
        if cross_y {
            cj += sj;
        }
        a = b;
        t0 = t1;
    }
}

#[cfg(test)]
mod tests {
    use super::super::Scratch;
    use super::*;

    /// Runs `splat` on a 4 x 4 pixel grid; the pixel values, `None` when it refused.
    fn on_4x4(splat: impl FnOnce(&mut Accum) -> bool) -> Option<Vec<f64>> {
        let mut data = vec![0i64; 16];
        let mut scratch = Scratch::default();
        let scale = (1u64 << 40) as f64;
        let mut acc = Accum {
            data: &mut data,
            scratch: &mut scratch,
            x0: 0,
            y0: 0,
            w: 4,
            h: 4,
            scale,
        };
        splat(&mut acc).then(|| data.iter().map(|&x| x as f64 / scale).collect())
    }

    /// Grids a unit value over a 4 x 4 pixel grid; `None` when the footprint is refused.
    fn grid_with(c: [[f64; 2]; 4], slope: Option<&Slope>) -> Option<Vec<f64>> {
        on_4x4(|acc| splat_linear(&c, 1.0, slope, acc))
    }

    fn grid(c: [[f64; 2]; 4]) -> Vec<f64> {
        grid_with(c, None).expect("footprint refused")
    }

    #[test]
    fn a_unit_square_across_four_pixels_splits_in_quarters() {
        let g = grid([[0.5, 0.5], [1.5, 0.5], [1.5, 1.5], [0.5, 1.5]]);
        for (i, x) in g.iter().enumerate() {
            let expect = if [0, 1, 4, 5].contains(&i) { 0.25 } else { 0.0 };
            assert!((x - expect).abs() < 1e-12, "{i} {x}");
        }
    }

    #[test]
    fn a_rotated_quad_conserves_value_and_orientation_does_not_matter() {
        let c = [[1.2, 0.3], [2.9, 1.1], [2.1, 2.8], [0.4, 1.9]];
        let g = grid(c);
        assert!((g.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let r = grid([c[3], c[2], c[1], c[0]]);
        for (a, b) in g.iter().zip(&r) {
            assert!((a - b).abs() < 1e-12);
        }
    }

    #[test]
    fn a_linear_slope_moves_energy_but_conserves_it() {
        let c = [[0.5, 0.5], [2.5, 0.5], [2.5, 1.5], [0.5, 1.5]];
        let (cen, a) = centroid_area(&c).unwrap();
        assert!(
            (cen[0] - 1.5).abs() < 1e-12 && (cen[1] - 1.0).abs() < 1e-12 && (a - 2.0).abs() < 1e-12
        );
        // Density 0.5 + 0.2 (u - 1.5): positive over the footprint.
        let slope = Slope {
            centroid: cen,
            grad: [0.2, 0.0],
        };
        let g = grid_with(c, Some(&slope)).expect("footprint refused");
        assert!((g.iter().sum::<f64>() - 1.0).abs() < 1e-9);
        // Pixel column 0 covers u in [0.5, 1]: integral of the density over [0.5,1]x[0.5,1].
        let exact = |u0: f64, u1: f64, v0: f64, v1: f64| {
            let f = |u: f64| 0.5 * u + 0.1 * (u - 1.5).powi(2);
            (f(u1) - f(u0)) * (v1 - v0)
        };
        assert!((g[0] - exact(0.5, 1.0, 0.5, 1.0)).abs() < 1e-9, "{}", g[0]);
        assert!((g[1] - exact(1.0, 2.0, 0.5, 1.0)).abs() < 1e-9, "{}", g[1]);
        assert!((g[2] - exact(2.0, 2.5, 0.5, 1.0)).abs() < 1e-9, "{}", g[2]);
    }

    /// The two cutting methods agree on footprints large enough for the edge sums, rotated,
    /// with and without a density slope, and on a 4 x 4 grid (no clipping at its border).
    #[test]
    fn edge_sums_and_peeling_agree() {
        let quads = [
            [[0.3, 0.2], [3.7, 0.9], [3.1, 3.8], [0.2, 2.9]],
            [[2.0, 0.1], [3.9, 2.0], [2.0, 3.9], [0.1, 2.0]],
            [[0.5, 0.5], [3.5, 0.5], [3.5, 2.25], [0.5, 2.25]],
        ];
        for c in quads {
            let (cen, _) = centroid_area(&c).unwrap();
            for slope in [
                None,
                Some(Slope {
                    centroid: cen,
                    grad: [0.01, -0.02],
                }),
            ] {
                let edges = grid_with(c, slope.as_ref()).expect("footprint refused");
                let total = area_moments(&c).0;
                let density = Density::new(1.0, total, slope.as_ref(), [0.0; 2]);
                let peeled = on_4x4(|acc| {
                    splat_peel(&c, (0, 3, 0, 3), density, acc);
                    true
                })
                .unwrap();
                let sum: f64 = edges.iter().sum();
                assert!((sum - 1.0).abs() < 1e-9, "{sum}");
                for (k, (&e, &p)) in edges.iter().zip(&peeled).enumerate() {
                    assert!((e - p).abs() < 1e-9, "{c:?} {slope:?} px {k}: {e} vs {p}");
                }
            }
        }
    }

    /// The edge sums' scratch is left all zero whatever the window cuts away (rows of another
    /// band are skipped, not read), so the next footprint sums from clean cells.
    #[test]
    fn the_scratch_is_clean_after_a_footprint_cut_by_the_window() {
        let big = [[0.3, 0.2], [3.7, 0.6], [3.4, 3.8], [0.5, 3.3]];
        let other = [[0.6, 0.4], [3.2, 0.1], [3.9, 3.5], [0.2, 3.7]];
        let slope = Slope {
            centroid: [2.0, 2.0],
            grad: [0.01, -0.02],
        };
        let run = |scratch: &mut Scratch, y0: i64, h: i64, c: &[[f64; 2]; 4]| {
            let mut data = vec![0i64; 4 * h as usize];
            let mut acc = Accum {
                data: &mut data,
                scratch,
                x0: 0,
                y0,
                w: 4,
                h,
                scale: (1u64 << 40) as f64,
            };
            assert!(splat_linear(c, 1.0, Some(&slope), &mut acc));
            data
        };
        let mut used = Scratch::default();
        let cut = run(&mut used, 2, 2, &big); // rows 0 and 1 are another band's
        assert!(cut.iter().any(|&x| x > 0));
        assert!(!used.cells.is_empty() && used.cells.iter().all(|&x| x == 0.0));
        let mut fresh = Scratch::default();
        assert_eq!(run(&mut used, 0, 4, &other), run(&mut fresh, 0, 4, &other));
    }

    #[test]
    fn a_folded_quad_is_refused() {
        assert!(grid_with([[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]], None).is_none());
    }
}
